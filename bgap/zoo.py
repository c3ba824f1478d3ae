from bgap.runner.numerics import command

main = command("bgap.commands.zoo")
if __name__ == "__main__":
    main()
