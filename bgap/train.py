from bgap.runner.numerics import command

main = command("bgap.commands.train")
if __name__ == "__main__":
    main()
