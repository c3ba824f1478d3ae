from bgap.runner.numerics import command

main = command("bgap.commands.figures")
if __name__ == "__main__":
    main()
